//! The shipped suite is consistent: every world loads in the simulator, every
//! instruction (derived ones included) parses into a plan with the embedded
//! HTN planner, every landmark it names exists in its world, destinations
//! lie in free space, and no start pose the noise can draw touches anything.

use std::path::Path;

use vlnav_eval::metrics::{Mode, Pose};
use vlnav_eval::runner::{contact_at, load_world};
use vlnav_eval::suite::{Suite, plan_trials};
use vlnav_planner::grounding::Grounder;
use vlnav_planner::htn;
use vlnav_planner::plan::{Action, Outcome};

fn suite() -> Suite {
    Suite::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/suite.toml")).expect("the shipped suite loads")
}

#[test]
fn the_suite_covers_the_papers_tables() {
    let s = suite();
    let v: Vec<&str> = s.scenarios.iter().filter_map(|c| c.paper_table_v.as_deref()).collect();
    for row in ["Indoor", "Garage", "Campus", "Forest", "Tunnel", "Indoor Lab"] {
        assert!(v.contains(&row), "no scenario stands for Table V's {row}");
    }
    let iv: Vec<&str> = s.scenarios.iter().filter_map(|c| c.paper_table_iv.as_deref()).collect();
    for row in vlnav_eval::paper::TABLE_IV.iter().map(|r| r.scenario) {
        assert!(iv.contains(&row), "no scenario stands for Table IV's {row}");
        let sc = s.scenarios.iter().find(|c| c.paper_table_iv.as_deref() == Some(row)).unwrap();
        assert_eq!(sc.modes(), Mode::ALL.to_vec(), "{row} needs an instruction per mode");
    }
    for sc in &s.scenarios {
        assert!(sc.instructions.len() >= 2, "{} carries fewer than two instructions", sc.name);
    }
    let lab = s.scenario("lab").unwrap();
    assert!(lab.world.ends_with("crates/simulator/scenarios/lab.toml"), "the lab is the simulator's own world");
}

#[test]
fn every_instruction_plans_and_names_landmarks_of_its_world() {
    let s = suite();
    let grounder = Grounder::lexical_only();
    for sc in &s.scenarios {
        let loaded = load_world(&sc.world_path(&s)).unwrap_or_else(|e| panic!("{}: {e:#}", sc.name));
        let w = &loaded.world;
        let start = Pose::new(w.start.x, w.start.y, w.start.theta);
        for ins in &sc.instructions {
            let text = ins.text(start);
            let plan = match htn::parse(&text, &grounder).outcome {
                Outcome::Plan(p) => p,
                Outcome::Clarify(c) => {
                    panic!("{} / {} ({text:?}): the planner asks {:?} ({})", sc.name, ins.id, c.question, c.reason)
                }
            };
            let who = format!("{} / {} ({text:?} → {})", sc.name, ins.id, plan.to_json_string());
            assert!(!plan.steps.is_empty(), "{who}: empty plan");
            let finds: Vec<i32> =
                plan.steps.iter().filter(|st| st.action == Action::Find).map(|st| st.class_id).collect();
            for class in &finds {
                assert!(!w.find_objects(*class, None, 0.0).is_empty(), "{who}: class {class} is not in the world");
            }
            match ins.mode {
                Mode::Geometric => assert!(finds.is_empty(), "{who}: a geometric instruction must not FIND"),
                Mode::Visual => assert!(
                    plan.steps.iter().all(|st| st.action == Action::Find),
                    "{who}: a visual instruction must only FIND"
                ),
                Mode::Hybrid => {}
            }
            if !ins.route.is_empty() && ins.mode != Mode::Geometric {
                let legs = ins.route.iter().filter(|l| l.find.is_some()).count();
                assert_eq!(finds.len(), legs, "{who}: FIND steps vs landmark legs");
            }
            // A mission ending at a landmark ends at most d_s + its half size (≤ 1 m) from it.
            let dest = ins.destination();
            if let Some(last) = plan.steps.last().filter(|st| st.action == Action::Find) {
                let reach = last.d_s.unwrap_or(2.0) + 1.0;
                let near = w
                    .find_objects(last.class_id, None, 0.0)
                    .iter()
                    .any(|(_, at)| (at.x - dest.x).hypot(at.y - dest.y) <= reach);
                assert!(near, "{who}: the destination is not by a {} of the world", last.target);
            }
            assert!(ins.radius >= 0.5, "{who}: radius below the executor's own arrival tolerance");
            if let Some(name) = &ins.follow {
                assert!(
                    w.pedestrian_index(name).is_some(),
                    "{who}: follows `{name}`, who is not a pedestrian of the world"
                );
                assert!(plan.steps.iter().any(|st| st.action == Action::Follow), "{who}: follows without a FOLLOW");
            }
        }
    }
}

#[test]
fn no_start_the_noise_can_draw_touches_anything() {
    let s = suite();
    for sc in &s.scenarios {
        let loaded = load_world(&sc.world_path(&s)).unwrap();
        let w = &loaded.world;
        let nominal = Pose::new(w.start.x, w.start.y, w.start.theta);
        let (xy, th) = sc.start_noise(&s.run);
        for dx in [-xy, xy] {
            for dy in [-xy, xy] {
                for dt in [-th, th] {
                    let p = nominal.compose(&Pose::new(dx, dy, dt));
                    assert_eq!(contact_at(w, p, 0.0), (false, false), "{}: start {p:?} is not free", sc.name);
                }
            }
        }
        // And the actual draws of a full run.
        for t in plan_trials(&s, 50, 1, &[]).iter().filter(|t| s.scenarios[t.scenario].name == sc.name) {
            let p = nominal.compose(&t.start_offset);
            assert_eq!(contact_at(w, p, 0.0), (false, false), "{} trial {}: start not free", sc.name, t.trial);
        }
    }
}

#[test]
fn a_full_run_plans_fifty_trials_per_scenario_and_mode() {
    let s = suite();
    let specs = plan_trials(&s, 50, 1, &[]);
    let groups: usize = s.scenarios.iter().map(|c| c.modes().len()).sum();
    assert_eq!(specs.len(), 50 * groups);
    assert_eq!(specs, plan_trials(&s, 50, 1, &[]), "the same seed plans the same trials");
}
