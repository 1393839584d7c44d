//! The validated world: solids (extruded shapes), floor markings, moving
//! pedestrians, and the instance table every rendered label refers to.

use crate::camera_config::CameraConfig;
use crate::geometry::{Pose2, Shape, Vec2};
use crate::robot::SlipModel;

/// Semantic class of an instance, as the segmenter contract names them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Semantic {
    Floor,
    Wall,
    Obstacle,
    Object,
    RestrictedZone,
    Cable,
    Hazard,
}

impl Semantic {
    pub fn as_str(self) -> &'static str {
        match self {
            Semantic::Floor => "floor",
            Semantic::Wall => "wall",
            Semantic::Obstacle => "obstacle",
            Semantic::Object => "object",
            Semantic::RestrictedZone => "restricted_zone",
            Semantic::Cable => "cable",
            Semantic::Hazard => "hazard",
        }
    }

    /// Entering a region of this class is a soft collision.
    pub fn is_no_go(self) -> bool {
        matches!(self, Semantic::RestrictedZone | Semantic::Cable | Semantic::Hazard)
    }
}

/// One instance of the world (label id `instance_id`, never 0).
#[derive(Clone, Debug, PartialEq)]
pub struct Entity {
    pub instance_id: u16,
    pub name: String,
    /// COCO-80 class id, −1 for structure, floor and markings.
    pub class_id: i32,
    /// Identity of a named person, lower case; empty otherwise.
    pub identity: String,
    pub semantic: Semantic,
}

/// A vertical prism standing on the floor: footprint extruded to `height`.
#[derive(Clone, Debug, PartialEq)]
pub struct Solid {
    pub entity: u16,
    pub shape: Shape,
    pub height: f64,
    pub color: [u8; 3],
}

/// A flat floor marking (restricted zone, hazard, cable), one or more shapes.
#[derive(Clone, Debug, PartialEq)]
pub struct Marking {
    pub entity: u16,
    pub shapes: Vec<Shape>,
    pub color: [u8; 3],
}

/// A person walking along waypoints at constant speed, a cylinder.
#[derive(Clone, Debug, PartialEq)]
pub struct Pedestrian {
    pub entity: u16,
    pub waypoints: Vec<Vec2>,
    pub speed: f64,
    pub looped: bool,
    pub radius: f64,
    pub height: f64,
    pub color: [u8; 3],
    /// Cumulative arc length at each waypoint along the walked route.
    cumulative: Vec<f64>,
}

impl Pedestrian {
    pub fn new(
        entity: u16,
        waypoints: Vec<Vec2>,
        speed: f64,
        looped: bool,
        radius: f64,
        height: f64,
        color: [u8; 3],
    ) -> Self {
        let mut route = waypoints.clone();
        if looped {
            route.push(waypoints[0]);
        }
        let mut cumulative = vec![0.0];
        for k in 1..route.len() {
            let l = cumulative[k - 1] + (route[k] - route[k - 1]).norm();
            cumulative.push(l);
        }
        Self { entity, waypoints, speed, looped, radius, height, color, cumulative }
    }

    /// Position at simulation time `t` (seconds since the episode began).
    pub fn position_at(&self, t: f64) -> Vec2 {
        let total = *self.cumulative.last().expect("at least two waypoints");
        let walked = self.speed * t.max(0.0);
        let s = if self.looped {
            walked % total
        } else {
            // Back and forth: fold the walked distance onto [0, total].
            let m = walked % (2.0 * total);
            if m > total { 2.0 * total - m } else { m }
        };
        let k = self.cumulative.partition_point(|&c| c <= s).clamp(1, self.cumulative.len() - 1);
        let n = self.waypoints.len();
        let a = self.waypoints[(k - 1) % n];
        let b = self.waypoints[k % n];
        let seg = self.cumulative[k] - self.cumulative[k - 1];
        let f = if seg > 0.0 { (s - self.cumulative[k - 1]) / seg } else { 0.0 };
        a + (b - a).scale(f)
    }

    pub fn shape_at(&self, t: f64) -> Shape {
        Shape::Circle { centre: self.position_at(t), radius: self.radius }
    }
}

/// A validated scenario.
#[derive(Clone, Debug, PartialEq)]
pub struct World {
    pub name: String,
    pub description: String,
    pub start: Pose2,
    pub camera: CameraConfig,
    pub slip: SlipModel,
    pub floor_color: [u8; 3],
    /// Instance table; `entities[i].instance_id == i + 1`, the floor is 1.
    pub entities: Vec<Entity>,
    pub solids: Vec<Solid>,
    pub markings: Vec<Marking>,
    pub pedestrians: Vec<Pedestrian>,
}

impl World {
    pub fn entity(&self, instance_id: u16) -> Option<&Entity> {
        (instance_id as usize).checked_sub(1).and_then(|i| self.entities.get(i))
    }

    /// The index (in `pedestrians`) of the pedestrian called `name`.
    pub fn pedestrian_index(&self, name: &str) -> Option<usize> {
        self.pedestrians.iter().position(|p| self.entity(p.entity).is_some_and(|e| e.name == name))
    }

    /// Entities of a COCO class (and identity, when given), with their
    /// position at time `t` (centre of the footprint's bounds).
    pub fn find_objects(&self, class_id: i32, identity: Option<&str>, t: f64) -> Vec<(&Entity, Vec2)> {
        let mut out = Vec::new();
        for s in &self.solids {
            let e = &self.entities[s.entity as usize - 1];
            if e.class_id == class_id && identity.is_none_or(|id| id == e.identity) {
                let (lo, hi) = s.shape.bounds();
                out.push((e, (lo + hi).scale(0.5)));
            }
        }
        for p in &self.pedestrians {
            let e = &self.entities[p.entity as usize - 1];
            if e.class_id == class_id && identity.is_none_or(|id| id == e.identity) {
                out.push((e, p.position_at(t)));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pedestrians_walk_loops_and_back_and_forth_at_their_speed() {
        let wps = vec![Vec2::new(0.0, 0.0), Vec2::new(2.0, 0.0)];
        let there_and_back = Pedestrian::new(2, wps.clone(), 1.0, false, 0.25, 1.7, [0, 0, 0]);
        assert_eq!(there_and_back.position_at(0.5), Vec2::new(0.5, 0.0));
        assert_eq!(there_and_back.position_at(3.0), Vec2::new(1.0, 0.0));
        assert_eq!(there_and_back.position_at(4.0), Vec2::new(0.0, 0.0));
        let square = vec![Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0)];
        let loop_walker = Pedestrian::new(2, square, 0.5, true, 0.25, 1.7, [0, 0, 0]);
        let p = loop_walker.position_at(7.0); // 3.5 m: halfway down the closing edge
        assert!((p.x - 0.0).abs() < 1e-12 && (p.y - 0.5).abs() < 1e-12, "{p:?}");
        assert_eq!(loop_walker.position_at(8.0), Vec2::new(0.0, 0.0));
    }
}
