//! Walking people: a social-force model (Helbing & Molnár 1995) in which each
//! person keeps to their route but slows, and steps aside, for walls, other
//! people and the robot within reach. The model and its constants are
//! described in `docs/simulation.md` ("People").
//!
//! A person's body is a circle; it never passes through a solid or the
//! robot's footprint: a step that would overlap one is not taken (the person
//! stops, as someone who bumps into a robot does). Deterministic: no random
//! draws, so the same robot motion gives the same crowd, bit for bit.

use crate::geometry::{OrientedRect, Shape, Vec2};
use crate::world::{Pedestrian, World};

/// Relaxation time towards the desired velocity, seconds.
pub const TAU_S: f64 = 0.5;
/// Repulsion between people: strength (m/s²) and range (m).
pub const PERSON_A: f64 = 2.1;
pub const PERSON_B: f64 = 0.3;
/// Repulsion from walls and furniture.
pub const SOLID_A: f64 = 3.0;
pub const SOLID_B: f64 = 0.2;
/// Repulsion from the robot: people keep more room from a machine.
pub const ROBOT_A: f64 = 4.0;
pub const ROBOT_B: f64 = 0.4;
/// How far ahead a person looks: repulsions are felt from where the two
/// would be after this long on their present courses (the stronger of that
/// and now), so people start to give way before they are close, seconds.
pub const ANTICIPATION_S: f64 = 1.0;
/// Weight of what is behind a person (1 would be isotropic).
pub const LAMBDA: f64 = 0.35;
/// Share of an opposing repulsion turned into a sidestep across the walking
/// direction (people pass an obstacle ahead instead of stopping in front of it).
pub const SIDESTEP: f64 = 0.6;
/// A person walks at most this multiple of their preferred speed.
pub const MAX_SPEED_FACTOR: f64 = 1.3;
/// A waypoint within this distance counts as reached, metres.
pub const WAYPOINT_REACH_M: f64 = 0.3;
/// Forces from farther than this are ignored, metres.
const INFLUENCE_M: f64 = 3.0;

/// One person's state.
#[derive(Clone, Debug, PartialEq)]
pub struct Walker {
    pub position: Vec2,
    pub velocity: Vec2,
    /// Index of the waypoint walked towards.
    target: usize,
    /// Back-and-forth routes: walking up (+1) or down (−1) the waypoints.
    direction: i8,
}

/// Every person of a world, stepped together.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Crowd {
    walkers: Vec<Walker>,
}

impl Crowd {
    /// Everyone at their first waypoint, already walking towards the second.
    pub fn new(world: &World) -> Self {
        let walkers = world
            .pedestrians
            .iter()
            .map(|p| {
                let start = p.waypoints[0];
                let heading = unit(p.waypoints[1] - start);
                Walker { position: start, velocity: heading.scale(p.speed), target: 1, direction: 1 }
            })
            .collect();
        Self { walkers }
    }

    pub fn walkers(&self) -> &[Walker] {
        &self.walkers
    }

    /// Where everyone is, in the world's pedestrian order.
    pub fn positions(&self) -> impl Iterator<Item = Vec2> + '_ {
        self.walkers.iter().map(|w| w.position)
    }

    /// Body outlines, in the world's pedestrian order.
    pub fn shapes<'a>(&'a self, world: &'a World) -> impl Iterator<Item = Shape> + 'a {
        world.pedestrians.iter().zip(&self.walkers).map(|(p, w)| Shape::Circle { centre: w.position, radius: p.radius })
    }

    /// Advances everyone by `h` seconds, the robot being at `robot` and
    /// moving at `robot_velocity` (world frame, m/s).
    pub fn step(&mut self, world: &World, robot: &OrientedRect, robot_velocity: Vec2, h: f64) {
        // Everyone reacts to where the others were at the start of the step.
        let before = self.walkers.clone();
        let ahead = OrientedRect {
            pose: vlnav_geometry::Pose2::new(
                robot.pose.x + robot_velocity.x * ANTICIPATION_S,
                robot.pose.y + robot_velocity.y * ANTICIPATION_S,
                robot.pose.theta,
            ),
            ..*robot
        };
        for i in 0..self.walkers.len() {
            let spec = &world.pedestrians[i];
            advance_target(&mut self.walkers[i], spec);
            let w = &self.walkers[i];
            let goal = route_point(spec, w.target);
            let e = unit(goal - w.position);
            let mut force = (e.scale(spec.speed) - w.velocity).scale(1.0 / TAU_S);

            for (j, other) in world.pedestrians.iter().enumerate() {
                if j == i {
                    continue;
                }
                let (other_at, other_v) = (before[j].position, before[j].velocity);
                if (w.position - other_at).norm() > INFLUENCE_M {
                    continue;
                }
                let mut push = Vec2::default();
                for t in [0.0, ANTICIPATION_S] {
                    let d = (w.position + w.velocity.scale(t)) - (other_at + other_v.scale(t));
                    let centre_gap = d.norm();
                    let gap = centre_gap - spec.radius - other.radius;
                    let n = if centre_gap > 1e-9 { d.scale(1.0 / centre_gap) } else { perpendicular_right(e) };
                    let f = repulsion(e, n, gap, PERSON_A, PERSON_B, true, other_at - w.position);
                    if f.norm() > push.norm() {
                        push = f;
                    }
                }
                force = force + push;
            }

            for s in &world.solids {
                let (lo, hi) = s.shape.bounds();
                let p = w.position;
                if p.x + INFLUENCE_M < lo.x
                    || p.x - INFLUENCE_M > hi.x
                    || p.y + INFLUENCE_M < lo.y
                    || p.y - INFLUENCE_M > hi.y
                {
                    continue;
                }
                let (q, inside) = s.shape.nearest_boundary_point(p);
                let d = p - q;
                let l = d.norm();
                let n = if l > 1e-9 { d.scale(if inside { -1.0 / l } else { 1.0 / l }) } else { e.scale(-1.0) };
                let gap = if inside { -l } else { l } - spec.radius;
                force = force + repulsion(e, n, gap, SOLID_A, SOLID_B, false, (lo + hi).scale(0.5) - p);
            }

            // The robot where it is, and where it will be shortly: the nearer.
            // Which side to pass it on: the one with room for the body
            // (walls and furniture beside the robot), else away from its centre.
            let room = |side: f64| {
                let right = perpendicular_right(e).scale(side);
                let centre: Vec2 = robot.pose.position().into();
                let reach = robot.half_length.hypot(robot.half_width) + spec.radius + 0.1;
                let at = centre + right.scale(reach);
                !world.solids.iter().any(|s| circle_overlaps_shape(at, spec.radius, &s.shape))
            };
            let prefer = match (room(1.0), room(-1.0)) {
                (true, false) => Some(1.0),
                (false, true) => Some(-1.0),
                _ => None,
            };
            let mut robot_push = Vec2::default();
            for (rect, t) in [(robot, 0.0), (&ahead, ANTICIPATION_S)] {
                let me = w.position + w.velocity.scale(t);
                let q = rect.nearest_point(me);
                let d = me - q;
                let l = d.norm();
                let n = if l > 1e-9 { d.scale(1.0 / l) } else { unit(me - rect.pose.position().into()) };
                let gap = l - spec.radius;
                // A preferred side is expressed as a centre on the other side.
                let centre = match prefer {
                    Some(side) => perpendicular_right(e).scale(-side),
                    None => Vec2::from(rect.pose.position()) - w.position,
                };
                let f = repulsion(e, n, gap, ROBOT_A, ROBOT_B, false, centre);
                if f.norm() > robot_push.norm() {
                    robot_push = f;
                }
            }
            force = force + robot_push;

            let w = &mut self.walkers[i];
            let mut v = w.velocity + force.scale(h);
            let cap = MAX_SPEED_FACTOR * spec.speed;
            if v.norm() > cap {
                v = v.scale(cap / v.norm());
            }
            let next = w.position + v.scale(h);
            let body = Shape::Circle { centre: next, radius: spec.radius };
            let blocked = robot.overlaps(&body)
                || world.solids.iter().any(|s| circle_overlaps_shape(next, spec.radius, &s.shape));
            if blocked {
                w.velocity = Vec2::default();
            } else {
                w.position = next;
                w.velocity = v;
            }
        }
    }
}

/// The repulsion a person walking along `e` feels from something whose
/// nearest point lies along −`n` at `gap` metres from the body's edge:
/// `A·exp(−gap/B)·n`, weighted by where it is (ahead counts fully), plus a
/// sidestep across `e` when it opposes the walk, away from the side the
/// thing's centre (at `centre` from the person) is on.
fn repulsion(e: Vec2, n: Vec2, gap: f64, a: f64, b: f64, anisotropic: bool, centre: Vec2) -> Vec2 {
    let magnitude = a * (-gap.max(-0.5) / b).exp();
    if magnitude < 1e-6 {
        return Vec2::default();
    }
    let cos_phi = -n.dot(e);
    let weight = if anisotropic { LAMBDA + (1.0 - LAMBDA) * (1.0 + cos_phi) / 2.0 } else { 1.0 };
    let mut f = n.scale(magnitude * weight);
    if cos_phi > 0.0 {
        // Pass on the side away from the thing's centre; dead ahead, keep right.
        let right = perpendicular_right(e);
        let side = if e.cross(centre) >= -1e-9 { right } else { right.scale(-1.0) };
        f = f + side.scale(SIDESTEP * magnitude * weight * cos_phi);
    }
    f
}

fn advance_target(w: &mut Walker, spec: &Pedestrian) {
    let n = spec.waypoints.len();
    if (route_point(spec, w.target) - w.position).norm() > WAYPOINT_REACH_M {
        return;
    }
    if spec.looped {
        w.target = (w.target + 1) % n;
    } else {
        let next = w.target as isize + w.direction as isize;
        if next < 0 || next >= n as isize {
            w.direction = -w.direction;
        }
        w.target = (w.target as isize + w.direction as isize) as usize;
    }
}

fn route_point(spec: &Pedestrian, k: usize) -> Vec2 {
    spec.waypoints[k % spec.waypoints.len()]
}

fn unit(v: Vec2) -> Vec2 {
    let l = v.norm();
    if l > 1e-12 { v.scale(1.0 / l) } else { Vec2::new(1.0, 0.0) }
}

fn perpendicular_right(e: Vec2) -> Vec2 {
    Vec2::new(e.y, -e.x)
}

fn circle_overlaps_shape(c: Vec2, r: f64, shape: &Shape) -> bool {
    let (lo, hi) = shape.bounds();
    if c.x + r < lo.x || c.x - r > hi.x || c.y + r < lo.y || c.y - r > hi.y {
        return false;
    }
    let (q, inside) = shape.nearest_boundary_point(c);
    inside || (c - q).norm() < r
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose2;
    use crate::scenario::parse;

    const HALL: &str = r#"
name = "hall"
[robot]
start = [0.0, -3.0, 0.0]
[[walls]]
path = [[-2, -4], [12, -4], [12, 4], [-2, 4]]
closed = true
"#;

    fn world(extra: &str) -> World {
        parse(&format!("{HALL}\n{extra}")).expect("valid world")
    }

    fn husky(x: f64, y: f64, theta: f64) -> OrientedRect {
        OrientedRect::new(Pose2::new(x, y, theta), 0.988, 0.670)
    }

    fn run(crowd: &mut Crowd, w: &World, robot: &OrientedRect, seconds: f64) -> f64 {
        // Returns the smallest gap between the first person and the robot.
        let mut closest = f64::INFINITY;
        for _ in 0..(seconds / 0.01) as usize {
            crowd.step(w, robot, Vec2::default(), 0.01);
            let p = crowd.walkers()[0].position;
            closest = closest.min((p - robot.nearest_point(p)).norm() - w.pedestrians[0].radius);
        }
        closest
    }

    #[test]
    fn an_unobstructed_person_keeps_to_the_route_at_their_speed() {
        let w = world("[[pedestrians]]\nwaypoints = [[0, 2], [8, 2]]\nspeed = 1.0\n");
        let mut crowd = Crowd::new(&w);
        let far = husky(0.0, -3.0, 0.0);
        for _ in 0..400 {
            crowd.step(&w, &far, Vec2::default(), 0.01);
        }
        let p = crowd.walkers()[0].position;
        assert!((p.x - 4.0).abs() < 0.2 && (p.y - 2.0).abs() < 0.05, "{p:?}");
        // Back and forth: after the far end (8 m) it turns round.
        for _ in 0..600 {
            crowd.step(&w, &far, Vec2::default(), 0.01);
        }
        let p = crowd.walkers()[0].position;
        assert!(p.x < 7.5 && crowd.walkers()[0].velocity.x < 0.0, "{p:?}");
    }

    #[test]
    fn a_person_walks_round_a_robot_standing_on_the_route_without_touching_it() {
        let w = world("[[pedestrians]]\nwaypoints = [[0, 0.05], [10, 0.05]]\nspeed = 1.2\n");
        let mut crowd = Crowd::new(&w);
        let robot = husky(5.0, 0.0, std::f64::consts::FRAC_PI_2);
        let closest = run(&mut crowd, &w, &robot, 12.0);
        assert!(closest > 0.1, "came within {closest:.3} m of the robot");
        let p = crowd.walkers()[0].position;
        assert!(p.x > 6.0, "the person got past the robot: {p:?}");
    }

    #[test]
    fn a_person_slows_for_a_robot_within_reach_and_never_overlaps_it() {
        // A robot parked across a 1.4 m corridor blocks it: the person stops
        // short and waits, touching nothing.
        let w = world(
            "[[walls]]\npath = [[-2, 0.7], [12, 0.7]]\n[[walls]]\npath = [[-2, -0.7], [12, -0.7]]\n\
             [[pedestrians]]\nwaypoints = [[0, 0], [10, 0]]\nspeed = 1.2\n",
        );
        let mut crowd = Crowd::new(&w);
        let robot = husky(5.0, 0.0, std::f64::consts::FRAC_PI_2);
        let closest = run(&mut crowd, &w, &robot, 15.0);
        assert!(closest > 0.0, "the person overlapped the robot ({closest:.3} m)");
        let walker = &crowd.walkers()[0];
        assert!(walker.position.x < 4.5 && walker.velocity.norm() < 0.2, "{walker:?}");
    }

    #[test]
    fn two_people_walking_at_each_other_pass() {
        let w = world(
            "[[pedestrians]]\nwaypoints = [[0, 0], [10, 0]]\nspeed = 1.2\n\
             [[pedestrians]]\nwaypoints = [[10, 0.1], [0, 0.1]]\nspeed = 1.2\n",
        );
        let mut crowd = Crowd::new(&w);
        let far = husky(0.0, -3.2, 0.0);
        let mut closest = f64::INFINITY;
        for _ in 0..700 {
            crowd.step(&w, &far, Vec2::default(), 0.01);
            let [a, b] = [crowd.walkers()[0].position, crowd.walkers()[1].position];
            closest = closest.min((a - b).norm() - 0.5);
        }
        assert!(closest > 0.0, "bodies overlapped by {:.3} m", -closest);
        assert!(crowd.walkers()[0].position.x > 7.0 && crowd.walkers()[1].position.x < 3.0);
    }
}
