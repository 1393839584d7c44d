//! The world generator: deterministic, every family's worlds load in the
//! simulator and their suite in the harness, every instruction plans with the
//! embedded HTN planner and names a landmark that is there and unambiguous,
//! and the feasibility check drops a blocked route and keeps an open one.

use std::path::PathBuf;

use vlnav_eval::metrics::{Mode, Pose};
use vlnav_eval::runner::contact_at;
use vlnav_eval::suite::{Suite, plan_trials};
use vlnav_eval::worlds::feasible::{Grid, Infeasible, check_route};
use vlnav_eval::worlds::{Family, dev_set, generate, generate_set, suite_toml, test_set};
use vlnav_planner::grounding::Grounder;
use vlnav_planner::htn;
use vlnav_planner::plan::{Action, Outcome};
use vlnav_sim::geometry::Vec2;

const PER_FAMILY: u64 = 6;

#[test]
fn the_same_seed_writes_the_same_bytes() {
    for f in Family::ALL {
        let a = generate(f, 17).unwrap();
        let b = generate(f, 17).unwrap();
        assert_eq!(a.toml, b.toml, "{f}: world");
        assert_eq!(suite_toml(std::slice::from_ref(&a), "x"), suite_toml(&[b], "x"), "{f}: suite");
        let c = generate(f, 18).unwrap();
        assert_ne!(a.toml, c.toml, "{f}: another seed, another world");
    }
    let dir_a = tempfile::tempdir().unwrap();
    let dir_b = tempfile::tempdir().unwrap();
    let which = dev_set(Family::Office, 3, 40).unwrap();
    generate_set(&which, dir_a.path(), "t").unwrap();
    generate_set(&which, dir_b.path(), "t").unwrap();
    for f in ["suite.toml", "dropped.csv"] {
        assert_eq!(
            std::fs::read(dir_a.path().join(f)).unwrap(),
            std::fs::read(dir_b.path().join(f)).unwrap(),
            "{f} differs between two runs of the same seeds"
        );
    }
}

#[test]
fn the_test_set_is_fixed_and_apart_from_development() {
    let t = test_set();
    assert!(t.len() >= 300, "{} worlds", t.len());
    assert!(t.iter().all(|(_, s)| *s >= 1_000_000));
    for f in Family::ALL {
        assert!(t.iter().any(|(g, _)| *g == f), "{f} missing from the test set");
    }
    assert_eq!(t, test_set());
    assert!(dev_set(Family::Hall, 10, 999_995).is_err(), "development seeds must stay below the test set's");
}

fn world_of(text: &str) -> vlnav_sim::world::World {
    vlnav_sim::scenario::parse(text).unwrap()
}

const ROOM: &str = r#"
name = "two rooms"
[robot]
start = [1.0, 0.0, 0.0]
[[walls]]
path = [[0.0, -2.0], [12.0, -2.0], [12.0, 2.0], [0.0, 2.0]]
closed = true
"#;

#[test]
fn a_blocked_route_is_infeasible_and_an_open_one_feasible() {
    let goal = [Vec2::new(10.0, 0.0)];
    // Open hall: feasible, about 9 m.
    let open = world_of(ROOM);
    let len = check_route(&Grid::new(&open), Vec2::new(1.0, 0.0), &goal).expect("an open hall is feasible");
    assert!((len - 9.0).abs() < 0.3, "{len}");
    // A partition across the hall: no way through.
    let wall = format!("{ROOM}[[walls]]\npath = [[6.0, -2.0], [6.0, 2.0]]\n");
    let e = check_route(&Grid::new(&world_of(&wall)), Vec2::new(1.0, 0.0), &goal).unwrap_err();
    assert!(matches!(e, Infeasible::Blocked { .. }), "{e}");
    // A doorway 1.2 m wide in it: the Husky (0.67 m) passes.
    let door =
        format!("{ROOM}[[walls]]\npath = [[6.0, -2.0], [6.0, -0.675]]\n[[walls]]\npath = [[6.0, 0.675], [6.0, 2.0]]\n");
    check_route(&Grid::new(&world_of(&door)), Vec2::new(1.0, 0.0), &goal).expect("a 1.2 m door is wide enough");
    // A doorway 0.6 m wide: narrower than the robot.
    let slit =
        format!("{ROOM}[[walls]]\npath = [[6.0, -2.0], [6.0, -0.375]]\n[[walls]]\npath = [[6.0, 0.375], [6.0, 2.0]]\n");
    assert!(check_route(&Grid::new(&world_of(&slit)), Vec2::new(1.0, 0.0), &goal).is_err());
    // A restricted zone across the hall blocks too (the robot keeps out of no-go markings).
    let zone = format!(
        "{ROOM}[[markings]]\nkind = \"restricted_zone\"\npolygon = [[6.0, -2.0], [7.0, -2.0], [7.0, 2.0], [6.0, 2.0]]\ncolor = [215, 30, 30]\n"
    );
    assert!(check_route(&Grid::new(&world_of(&zone)), Vec2::new(1.0, 0.0), &goal).is_err());
    // A waypoint with no room to turn.
    let tight = [Vec2::new(11.4, 0.0), Vec2::new(5.0, 0.0)];
    let e = check_route(&Grid::new(&open), Vec2::new(1.0, 0.0), &tight).unwrap_err();
    assert!(matches!(e, Infeasible::NoRoomToTurn { index: 1, .. }), "{e}");
}

/// Generates `PER_FAMILY` development worlds of every family into a temp dir.
fn generated() -> (tempfile::TempDir, PathBuf, usize) {
    let dir = tempfile::tempdir().unwrap();
    let mut which = Vec::new();
    for f in Family::ALL {
        which.extend(dev_set(f, PER_FAMILY, 100).unwrap());
    }
    let rep = generate_set(&which, dir.path(), "test").unwrap();
    assert_eq!(rep.worlds_generated, which.len());
    let path = rep.suite.clone();
    (dir, path, rep.instructions_dropped)
}

#[test]
fn every_family_writes_worlds_the_simulator_loads_and_instructions_the_planner_parses() {
    let (_dir, path, _dropped) = generated();
    let suite = Suite::load(&path).expect("the generated suite loads");
    let grounder = Grounder::lexical_only();
    for f in Family::ALL {
        let n = suite.scenarios.iter().filter(|s| s.family.as_deref() == Some(f.as_str())).count();
        assert!(n as u64 >= PER_FAMILY / 2, "{f}: only {n} of {PER_FAMILY} worlds kept");
    }
    for sc in &suite.scenarios {
        let loaded = vlnav_eval::runner::load_world(&sc.world_path(&suite)).unwrap();
        let w = &loaded.world;
        let start = Pose::new(w.start.x, w.start.y, w.start.theta);
        assert!(sc.instructions.iter().any(|i| i.mode == Mode::Hybrid), "{}: no hybrid instruction", sc.name);
        for ins in &sc.instructions {
            let text = ins.text(start);
            let who = format!("{} / {} ({text:?})", sc.name, ins.id);
            let plan = match htn::parse(&text, &grounder).outcome {
                Outcome::Plan(p) => p,
                Outcome::Clarify(c) => panic!("{who}: the planner asks {:?} ({})", c.question, c.reason),
            };
            let finds: Vec<_> = plan.steps.iter().filter(|s| s.action == Action::Find).collect();
            let leg = ins.route.last().unwrap();
            match ins.mode {
                Mode::Geometric => assert!(finds.is_empty(), "{who}: FIND in a geometric instruction"),
                _ => {
                    assert_eq!(finds.len(), 1, "{who}: one landmark");
                    let find = finds[0];
                    assert_eq!(find.d_s, leg.d_s, "{who}: the spoken stopping distance");
                    let instances = w.find_objects(find.class_id, None, 0.0);
                    assert!(
                        instances.iter().any(|(_, c)| (c.x - leg.at[0]).abs() < 0.01 && (c.y - leg.at[1]).abs() < 0.01),
                        "{who}: no class {} at the route's landmark",
                        find.class_id
                    );
                    // Unambiguous: with no reference named, no other
                    // instance is nearer the last waypoint than the target plus 3 m
                    // unless a wall hides it (checked by the generator); the
                    // visual mode only where the class is unique.
                    if ins.mode == Mode::Visual {
                        assert_eq!(instances.len(), 1, "{who}: a visual instruction names a unique class");
                    }
                    if find.reference.is_some() {
                        assert!(text.contains(" next to the "), "{who}");
                    }
                }
            }
            if ins.mode == Mode::Hybrid {
                assert_eq!(plan.steps.last().map(|s| s.action), Some(Action::Find), "{who}: ends at the landmark");
            }
            let stop = ins.stop_distance(w);
            assert!(stop > leg.d_s.unwrap() && ins.radius > stop, "{who}: d {stop}, r {}", ins.radius);
        }
        // No start the noise can draw touches anything.
        let (xy, th) = sc.start_noise(&suite.run);
        for dx in [-xy, xy] {
            for dy in [-xy, xy] {
                for dt in [-th, th] {
                    let p = start.compose(&Pose::new(dx, dy, dt));
                    assert_eq!(contact_at(w, p, 0.0), (false, false), "{}: start {p:?} is not free", sc.name);
                }
            }
        }
    }
    assert!(!plan_trials(&suite, 1, 1, &[]).is_empty());
}

#[test]
fn a_world_is_dropped_when_its_route_is_blocked() {
    // Block the generated route with a wall across the hybrid's last waypoint: the check drops it.
    let w = (0..20).map(|s| generate(Family::Hall, s).unwrap()).find(|w| !w.instructions.is_empty()).unwrap();
    let ins = &w.instructions[0];
    let p = *ins.route.last().unwrap();
    let blocked =
        format!("{}\n[[walls]]\npath = [[{:.2}, -100.0], [{:.2}, 100.0]]\n", w.toml, p[0] + 0.01, p[0] + 0.01);
    let world = world_of(&blocked);
    let start = Vec2::new(world.start.x, world.start.y);
    let pts: Vec<Vec2> = ins.route.iter().map(|q| Vec2::new(q[0], q[1])).collect();
    assert!(check_route(&Grid::new(&world), start, &pts).is_err());
    assert!(check_route(&Grid::new(&world_of(&w.toml)), start, &pts).is_ok());
}

#[test]
fn dropped_instructions_are_listed() {
    let (dir, _path, dropped) = generated();
    let csv = std::fs::read_to_string(dir.path().join("dropped.csv")).unwrap();
    assert_eq!(csv.lines().count() - 1, dropped, "dropped.csv lists every dropped instruction");
}

#[test]
fn the_shipped_suite_has_no_families_so_its_report_is_unchanged() {
    // The per-family section is added only for suites whose scenarios carry a family.
    let shipped = Suite::load(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenarios/suite.toml")).unwrap();
    assert!(shipped.scenarios.iter().all(|s| s.family.is_none()));
}
