//! Behaviour of the simulator as a whole: determinism, rendering against
//! known geometry, collision accounting, odometry drift, shipped scenarios.

use vlnav_sim::geometry::{OrientedRect, Shape, Vec2};
use vlnav_sim::{Frame, Pose2, Semantic, Simulator, SlipModel, Twist, World, load_scenario, scenario};

fn world(text: &str) -> World {
    scenario::parse(text).unwrap_or_else(|e| panic!("test scenario invalid: {e}"))
}

const CORRIDOR: &str = r#"
name = "corridor"
[robot]
start = [0.0, 0.0, 0.0]
[camera]
depth_noise_k = 0.0
[[walls]]
path = [[-2.0, -2.0], [12.0, -2.0], [12.0, 2.0], [-2.0, 2.0]]
closed = true
thickness = 0.2
height = 2.5
[[objects]]
name = "box ahead"
class_id = 56
position = [5.3, 0.0]
shape = "box"
size = [0.6, 1.0]
height = 1.0
color = [200, 120, 40]
[[markings]]
kind = "restricted_zone"
polygon = [[2.0, -1.0], [3.0, -1.0], [3.0, 1.0], [2.0, 1.0]]
color = [215, 30, 30]
"#;

fn run_commands(sim: &mut Simulator, commands: &[(Twist, usize)], frames: &mut Vec<Frame>) -> Vec<(Pose2, Pose2)> {
    let mut traj = Vec::new();
    for &(cmd, n) in commands {
        for _ in 0..n {
            sim.step(cmd, 0.1);
            traj.push((sim.truth().pose, sim.odometry().pose));
            frames.push(sim.render());
        }
    }
    traj
}

#[test]
fn same_scenario_seed_and_commands_give_a_bit_identical_run() {
    let commands = [
        (Twist::new(0.8, 0.0), 20),
        (Twist::new(0.5, 1.2), 15),
        (Twist::new(1.0, -0.4), 25),
        (Twist::new(0.0, 2.0), 10),
    ];
    let run = |seed: u64| {
        let mut sim = Simulator::new(load_scenario("demo").unwrap(), seed);
        sim.set_camera(sim.camera().clone().with_resolution(160, 120).unwrap());
        let mut frames = Vec::new();
        let traj = run_commands(&mut sim, &commands, &mut frames);
        (traj, frames, sim.truth())
    };
    let (a, fa, ta) = run(42);
    let (b, fb, tb) = run(42);
    let bits = |t: &[(Pose2, Pose2)]| -> Vec<u64> {
        t.iter().flat_map(|(p, o)| [p.x, p.y, p.theta, o.x, o.y, o.theta]).map(f64::to_bits).collect()
    };
    assert_eq!(bits(&a), bits(&b));
    assert!(fa == fb, "rendered frames differ between identical runs");
    assert_eq!(ta, tb);
    // A different seed changes the slip noise, hence the truth (odometry is the same wheels).
    let (c, _, _) = run(43);
    assert_ne!(bits(&a), bits(&c));
}

#[test]
fn rendering_matches_the_geometry_it_was_given() {
    let mut sim = Simulator::new(world(CORRIDOR), 0);
    let f = sim.render();
    let cam = sim.camera().clone();
    let (cu, _) = (cam.cx.round() as u32, cam.cy.round() as u32);
    // The centre column looks down the corridor at the box's near face, 5.0 m
    // from base_link, 4.7 m from the camera (mounted 0.30 m ahead).
    let v_box = (cam.cy - 0.3 / 4.7 * cam.fy).round() as u32; // 0.3 m high on the box face (camera at 0.6)
    let (rgb, depth, label) = f.pixel(cu, v_box);
    assert_eq!(depth, 4700, "depth at the box face");
    let e = f.instances.iter().find(|e| e.instance_id == label).expect("label in table");
    assert_eq!((e.class_id, e.semantic), (56, Semantic::Object));
    assert!(rgb[0] > rgb[1] && rgb[1] > rgb[2], "box colour keeps its hue: {rgb:?}");
    // A floor pixel 2.5 m ahead lies in the red zone (x 2–3 m in the world).
    let z_floor = 2.5 - 0.3;
    let v_floor = (cam.cy + 0.6 / z_floor * cam.fy).round() as u32;
    let (rgb, depth, label) = f.pixel(cu, v_floor);
    let e = f.instances.iter().find(|e| e.instance_id == label).unwrap();
    assert_eq!(e.semantic, Semantic::RestrictedZone);
    assert!((depth as f64 - z_floor * 1000.0).abs() < 15.0, "floor depth {depth}");
    let (h, s, v) = hsv(rgb);
    assert!(
        (h <= 10.0 || h >= 170.0) && s >= 120.0 && v >= 70.0,
        "red zone must pass an HSV red mask: {rgb:?} → {h} {s} {v}"
    );
    // Floor just in front of the camera is closer than 0.3 m of depth? No —
    // the bottom row sees the floor at 0.6/(240.5/343) ≈ 0.86 m: valid.
    let (_, depth, label) = f.pixel(cu, cam.height - 1);
    assert!(depth > 800 && depth < 900, "bottom row floor depth {depth}");
    assert_eq!(label, 1);
    // Slightly above the horizon the column meets the far wall (11.6 m of
    // optical depth, beyond the 10 m range): no depth, but a wall label.
    let (_, depth, label) = f.pixel(cu, (cam.cy - 0.1 * cam.fy).round() as u32);
    assert_eq!(depth, 0);
    let wall = f.instances.iter().find(|e| e.instance_id == label).unwrap();
    assert_eq!(wall.semantic, Semantic::Wall);
    // The top row looks over the 2.5 m wall: sky, label 0, no depth.
    assert_eq!(f.pixel(cu, 0).1, 0);
    assert_eq!(f.pixel(cu, 0).2, 0);
    // Every label used appears in the instance table and vice versa.
    let mut used: Vec<u16> = f.labels.iter().copied().filter(|&l| l != 0).collect();
    used.sort_unstable();
    used.dedup();
    let mut table: Vec<u16> = f.instances.iter().map(|e| e.instance_id).collect();
    table.sort_unstable();
    assert_eq!(used, table);
}

fn hsv(rgb: [u8; 3]) -> (f64, f64, f64) {
    let [r, g, b] = rgb.map(|c| c as f64);
    let max = r.max(g).max(b);
    let min = r.min(g).min(b);
    let d = max - min;
    let h = if d == 0.0 {
        0.0
    } else if max == r {
        60.0 * (((g - b) / d).rem_euclid(6.0))
    } else if max == g {
        60.0 * ((b - r) / d + 2.0)
    } else {
        60.0 * ((r - g) / d + 4.0)
    };
    // OpenCV scale: H in 0–180, S and V in 0–255.
    (h / 2.0, if max == 0.0 { 0.0 } else { d / max * 255.0 }, max)
}

#[test]
fn depth_noise_and_range_limits_apply() {
    let mut w = world(CORRIDOR);
    w.camera.depth_noise_k = 0.01;
    let mut sim = Simulator::new(w, 5);
    let f = sim.render();
    let cam = sim.camera().clone();
    // Along the box face (4.7 m), σ = 0.01·4.7² ≈ 0.22 m: values scatter around 4.7 m.
    let v = (cam.cy - 0.3 / 4.7 * cam.fy).round() as u32;
    let row: Vec<f64> = (300..340).map(|u| f.pixel(u, v).1 as f64 / 1000.0).collect();
    let mean = row.iter().sum::<f64>() / row.len() as f64;
    let sd = (row.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / row.len() as f64).sqrt();
    assert!((mean - 4.7).abs() < 0.15, "mean {mean}");
    assert!(sd > 0.1 && sd < 0.4, "sd {sd}");
    assert!(f.depth_mm.iter().all(|&d| d == 0 || (300..=10_000).contains(&d)));
}

#[test]
fn driving_into_a_wall_is_one_hard_collision_and_crossing_a_zone_one_soft() {
    let mut w = world(CORRIDOR);
    w.slip = SlipModel::none();
    let mut sim = Simulator::new(w, 0);
    // Straight ahead through the red zone (x 2–3) into the box at x 5.0.
    for _ in 0..100 {
        sim.step(Twist::new(1.0, 0.0), 0.1);
    }
    let t = sim.truth();
    assert_eq!(t.soft_collisions, 1, "one entry into the zone, however many frames inside");
    assert_eq!(t.hard_collisions, 1, "pressing against the box is one contact");
    // The body stopped at the box (its front 0.494 m ahead of the centre).
    assert!(t.pose.x > 4.45 && t.pose.x < 4.51, "stopped at {}", t.pose.x);
    assert!((t.path_length_m - t.pose.x).abs() < 1e-9);
    // The wheels kept spinning: odometry overshoots the truth.
    assert!(sim.odometry().pose.x > t.pose.x + 3.0);
    // Back off and push again: a second contact event.
    for _ in 0..10 {
        sim.step(Twist::new(-0.5, 0.0), 0.1);
    }
    for _ in 0..20 {
        sim.step(Twist::new(0.5, 0.0), 0.1);
    }
    assert_eq!(sim.truth().hard_collisions, 2);
    assert_eq!(sim.truth().soft_collisions, 1);
}

#[test]
fn odometry_drifts_from_truth_and_reset_re_anchors_it() {
    let mut sim = Simulator::new(load_scenario("demo").unwrap(), 3);
    for _ in 0..30 {
        sim.step(Twist::new(0.6, 0.8), 0.1);
    }
    let t = sim.truth();
    let believed = sim.odom_to_world(&sim.odometry().pose);
    let drift = believed.distance(&t.pose);
    assert!(drift > 0.005 && drift < 0.5, "drift after a 3 s turn: {drift}");
    sim.reset_odometry();
    let t = sim.truth();
    assert_eq!(t.odom_origin, t.pose);
    assert_eq!(sim.odometry().pose, Pose2::default());
}

fn view(world: &World, pose: Pose2) -> (Frame, Simulator) {
    let mut w = world.clone();
    w.start = pose;
    let mut sim = Simulator::new(w, 0);
    (sim.render(), sim)
}

fn pixels_of(frame: &Frame, name: &str) -> usize {
    let ids: Vec<u16> = frame.instances.iter().filter(|e| e.name == name).map(|e| e.instance_id).collect();
    frame.labels.iter().filter(|l| ids.contains(l)).count()
}

fn object_position(world: &World, name: &str) -> Vec2 {
    let id = world.entities.iter().find(|e| e.name == name).unwrap_or_else(|| panic!("no {name}")).instance_id;
    let s = world.solids.iter().find(|s| s.entity == id).unwrap();
    let (lo, hi) = s.shape.bounds();
    (lo + hi).scale(0.5)
}

/// Where a FIND step that starts at `from` stops: `d_s` short of the target, facing it.
fn stop_short(from: Vec2, target: Vec2, d_s: f64) -> Pose2 {
    let d = target - from;
    let l = d.norm();
    let p = from + d.scale((l - d_s) / l);
    Pose2::new(p.x, p.y, d.y.atan2(d.x))
}

fn move_step(p: Pose2, yaw: f64, f: f64) -> Pose2 {
    let th = p.theta + yaw;
    Pose2::new(p.x + f * th.cos(), p.y + f * th.sin(), th)
}

#[test]
fn demo_makes_both_paper_instructions_meaningful() {
    let w = load_scenario("demo").unwrap();
    let statue = object_position(&w, "statue (human)");
    let person = object_position(&w, "standing person");
    let chair = object_position(&w, "visitor chair");
    let bicycle = object_position(&w, "bicycle");
    let persons_in_view =
        |f: &Frame| f.instances.iter().filter(|e| e.class_id == 0).map(|e| e.name.clone()).collect::<Vec<_>>();

    // Case 1: the statue is the one person in view at the start.
    let start = w.start;
    let (f, _) = view(&w, start);
    assert_eq!(persons_in_view(&f), vec!["statue (human)".to_string()]);
    assert!(pixels_of(&f, "statue (human)") > 500);
    assert!((statue - Vec2::from(start.position())).norm() <= 10.0);
    let at_statue = stop_short(Vec2::from(start.position()), statue, 2.0);
    let turned = move_step(at_statue, -std::f64::consts::FRAC_PI_2, 2.5);
    let (f, _) = view(&w, turned);
    assert!(pixels_of(&f, "visitor chair") > 500, "chair ahead after the right turn");
    assert!((chair - Vec2::from(turned.position())).norm() <= 10.0);
    let at_chair = stop_short(Vec2::from(turned.position()), chair, 1.5);
    let (f, _) = view(&w, at_chair);
    assert!(pixels_of(&f, "bicycle") > 500, "bicycle in view on the right of the chair");
    let rel = at_chair.relative(&Pose2::new(bicycle.x, bicycle.y, 0.0));
    assert!(rel.y < 0.0, "bicycle is to the right");

    // Case 2: left turn, 4 m, the standing person is in view; the statue is not.
    let after_move = move_step(start, std::f64::consts::FRAC_PI_2, 4.0);
    let (f, _) = view(&w, after_move);
    assert_eq!(persons_in_view(&f), vec!["standing person".to_string()]);
    assert!((person - Vec2::from(after_move.position())).norm() <= 10.0);
    let at_person = stop_short(Vec2::from(after_move.position()), person, 2.0);
    let rel = at_person.relative(&Pose2::new(chair.x, chair.y, 0.0));
    assert!(rel.y < 0.0 && (chair - Vec2::from(at_person.position())).norm() <= 10.0, "chair on the right within 10 m");
    // Scanning right by 30° steps brings the chair into view.
    let found = (1..=4).any(|k| {
        let (f, _) = view(&w, Pose2::new(at_person.x, at_person.y, at_person.theta - k as f64 * 30f64.to_radians()));
        pixels_of(&f, "visitor chair") > 200
    });
    assert!(found, "a scan to the right finds the chair");
    // The naive straight line from the person to the chair crosses the red zone.
    let zone =
        &w.markings.iter().find(|m| w.entity(m.entity).unwrap().semantic == Semantic::RestrictedZone).unwrap().shapes
            [0];
    let crosses = (0..=100).any(|i| {
        let p = Vec2::from(at_person.position()) + (chair - Vec2::from(at_person.position())).scale(i as f64 / 100.0);
        OrientedRect::new(Pose2::new(p.x, p.y, at_person.theta), 0.988, 0.67).overlaps(zone)
    });
    assert!(crosses);
    let at_chair = stop_short(Vec2::from(at_person.position()), chair, 1.5);
    let (f, _) = view(&w, at_chair);
    assert!(pixels_of(&f, "bicycle") > 500);
    // The red zone looks red from where it matters.
    let (f, _) = view(&w, Pose2::new(at_person.x, at_person.y, (chair.y - at_person.y).atan2(chair.x - at_person.x)));
    assert!(f.instances.iter().any(|e| e.semantic == Semantic::RestrictedZone));
    assert!(matches!(zone, Shape::Polygon(_)));
}

#[test]
fn lab_is_ten_by_five_and_a_half_with_its_objects_within_reach() {
    let w = load_scenario("lab").unwrap();
    let count = |c: i32| w.entities.iter().filter(|e| e.class_id == c).count();
    assert!(count(39) >= 2 && count(56) >= 2 && count(58) >= 2);
    assert!(w.entities.iter().any(|e| e.semantic == Semantic::Cable));
    assert!(w.entities.iter().any(|e| e.semantic == Semantic::RestrictedZone));
    for e in w.entities.iter().filter(|e| e.class_id >= 0) {
        let p = object_position(&w, &e.name);
        assert!(p.x > 0.0 && p.x < 10.0 && p.y > 0.0 && p.y < 5.5, "{} inside the room", e.name);
        assert!((p - Vec2::from(w.start.position())).norm() <= 10.0);
    }
    // Looking down the room from the start: chairs, bottles and the red zone are visible at 640×480.
    let (f, _) = view(&w, w.start);
    assert!(f.instances.iter().any(|e| e.class_id == 56));
    assert!(f.instances.iter().any(|e| e.class_id == 39));
    assert!(f.instances.iter().any(|e| e.semantic == Semantic::RestrictedZone));
    assert!(f.instances.iter().any(|e| e.semantic == Semantic::Cable));
}

#[test]
fn pedestrians_move_and_are_rendered_as_persons() {
    let w = load_scenario("demo").unwrap();
    let p = &w.pedestrians[0];
    assert_ne!(p.position_at(0.0), p.position_at(4.0));
    // Look at the walkway from the south-east.
    let (f, _) = view(&w, Pose2::new(6.0, -5.0, (-1.5f64).atan2(-6.0)));
    let ped = f.instances.iter().find(|e| e.name == "walking pedestrian").expect("pedestrian in view");
    assert_eq!(ped.class_id, 0);
    assert_eq!(ped.semantic, Semantic::Object);
}

/// A corridor 1.4 m wide: a person and the Husky cannot pass each other.
const NARROW: &str = r#"
name = "narrow"
[robot]
start = [1.0, 0.0, 0.0]
[[walls]]
path = [[-1, -0.7], [14, -0.7]]
[[walls]]
path = [[-1, 0.7], [14, 0.7]]
[[pedestrians]]
name = "walker"
waypoints = [[12, 0], [-0.5, 0]]
speed = 1.0
"#;

#[test]
fn a_robot_driving_into_a_person_made_the_contact() {
    let mut w = world(NARROW);
    w.slip = SlipModel::none();
    let mut sim = Simulator::new(w, 0);
    for _ in 0..100 {
        sim.step(Twist::new(0.8, 0.0), 0.1);
    }
    let t = sim.truth();
    assert!(t.pedestrian_contacts >= 1, "{t:?}");
    assert_eq!(t.pedestrian_contacts_by_robot, t.pedestrian_contacts, "the robot kept driving at the person");
    assert_eq!(t.hard_collisions_by_robot, t.hard_collisions);
    assert_eq!(t.pedestrians.len(), 1);
}

#[test]
fn a_person_who_meets_a_stopped_robot_stops_short_and_one_who_runs_into_it_made_the_contact() {
    let mut w = world(NARROW);
    w.slip = SlipModel::none();
    let mut sim = Simulator::new(w.clone(), 0);
    for _ in 0..150 {
        sim.step(Twist::ZERO, 0.1);
    }
    let t = sim.truth();
    assert_eq!(t.hard_collisions, 0, "a walking person keeps off a robot that stands in the way");
    let person = t.pedestrians[0];
    assert!(person.x > 1.6 && person.x < 3.0, "waits in front of the robot: {person:?}");
    // Someone running (2.8 m/s) cannot stop in time: contact, theirs.
    let text = NARROW.replace("speed = 1.0", "speed = 2.8");
    let mut w = world(&text);
    w.slip = SlipModel::none();
    let mut sim = Simulator::new(w, 0);
    for _ in 0..80 {
        sim.step(Twist::ZERO, 0.1);
    }
    let t = sim.truth();
    assert!(t.pedestrian_contacts >= 1, "{t:?}");
    assert_eq!(t.pedestrian_contacts_by_robot, 0);
    assert_eq!(t.hard_collisions_by_robot, 0);
}
