//! Scenario files (TOML) and their validation into a [`World`].
//!
//! ```toml
//! name = "example"
//! [robot]
//! start = [0.0, 0.0, 0.0]          # x, y (m), heading (rad) in the world frame
//! [camera]                         # optional; defaults: 640×480, paper intrinsics, mount x 0.30 z 0.60
//! [[walls]]                        # polylines extruded to thin prisms
//! path = [[-1, -3], [9, -3], [9, 3], [-1, 3]]
//! closed = true
//! thickness = 0.15
//! height = 2.0
//! [[obstacles]]                    # simple polygons extruded to `height`
//! polygon = [[2, 1], [3, 1], [3, 2]]
//! height = 0.8
//! [[objects]]                      # labelled COCO objects, box or cylinder
//! name = "statue"
//! class_id = 0
//! position = [6.0, 0.0]
//! shape = "cylinder"
//! radius = 0.3
//! height = 1.8
//! [[markings]]                     # floor markings: restricted_zone or hazard
//! kind = "restricted_zone"
//! polygon = [[1, -1], [2, -1], [2, 1], [1, 1]]
//! color = [220, 30, 30]
//! [[cables]]
//! path = [[0, 2], [4, 2.5]]
//! [[pedestrians]]
//! identity = "david"
//! waypoints = [[3, 2], [3, -2]]
//! speed = 0.6
//! ```
//!
//! Every validation error names the offending field (`objects[2].class_id`).

use serde::Deserialize;

use crate::camera::CameraConfig;
use crate::geometry::{OrientedRect, Pose2, Shape, Vec2, box_polygon, segment_quad, self_intersection, signed_area2};
use crate::robot::{HuskyParams, SlipModel};
use crate::world::{Entity, Marking, Pedestrian, Semantic, Solid, World};

/// A scenario file was unreadable or invalid.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ScenarioError {
    #[error("scenario is not valid TOML: {0}")]
    Syntax(String),
    #[error("{field}: {message}")]
    Invalid { field: String, message: String },
    #[error("unknown scenario `{name}`; shipped scenarios: {known}")]
    UnknownName { name: String, known: String },
    #[error("cannot read scenario file {path}: {message}")]
    Io { path: String, message: String },
}

impl ScenarioError {
    fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        ScenarioError::Invalid { field: field.into(), message: message.into() }
    }

    /// The field an invalid scenario names, if any.
    pub fn field(&self) -> Option<&str> {
        match self {
            ScenarioError::Invalid { field, .. } => Some(field),
            _ => None,
        }
    }
}

type Point = [f64; 2];
type Rgb = [u8; 3];

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct ScenarioFile {
    pub name: String,
    #[serde(default)]
    pub description: String,
    pub robot: RobotSpec,
    #[serde(default)]
    pub camera: CameraSpec,
    #[serde(default)]
    pub floor_color: Option<Rgb>,
    #[serde(default)]
    pub walls: Vec<WallSpec>,
    #[serde(default)]
    pub obstacles: Vec<ObstacleSpec>,
    #[serde(default)]
    pub objects: Vec<ObjectSpec>,
    #[serde(default)]
    pub markings: Vec<MarkingSpec>,
    #[serde(default)]
    pub cables: Vec<CableSpec>,
    #[serde(default)]
    pub pedestrians: Vec<PedestrianSpec>,
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct RobotSpec {
    /// x, y (m), heading (rad).
    pub start: [f64; 3],
    #[serde(default)]
    pub slip: Option<SlipModel>,
}

#[derive(Deserialize, Debug, Clone, Default)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub fx: Option<f64>,
    pub fy: Option<f64>,
    pub cx: Option<f64>,
    pub cy: Option<f64>,
    /// Camera body position in base_link, metres.
    pub mount: Option<[f64; 3]>,
    /// Camera yaw in base_link, radians (the renderer needs a level camera: no roll or pitch).
    pub mount_yaw: Option<f64>,
    pub depth_min_m: Option<f64>,
    pub depth_max_m: Option<f64>,
    /// Depth noise σ = k·z² (metres), k in 1/m.
    pub depth_noise_k: Option<f64>,
    /// Beyond this range pixels start to lose their depth, metres.
    pub depth_reliable_max_m: Option<f64>,
    /// Stereo baseline for occlusion holes at depth edges, metres (0: none).
    pub stereo_baseline_m: Option<f64>,
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct WallSpec {
    #[serde(default)]
    pub name: Option<String>,
    pub path: Vec<Point>,
    #[serde(default)]
    pub closed: bool,
    #[serde(default = "default_wall_thickness")]
    pub thickness: f64,
    #[serde(default = "default_wall_height")]
    pub height: f64,
    #[serde(default)]
    pub color: Option<Rgb>,
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct ObstacleSpec {
    #[serde(default)]
    pub name: Option<String>,
    pub polygon: Vec<Point>,
    pub height: f64,
    #[serde(default)]
    pub color: Option<Rgb>,
}

#[derive(Deserialize, Debug, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum ShapeKind {
    Box,
    Cylinder,
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct ObjectSpec {
    #[serde(default)]
    pub name: Option<String>,
    pub class_id: i32,
    #[serde(default)]
    pub identity: Option<String>,
    pub position: Point,
    pub shape: ShapeKind,
    /// Box: footprint [length along x, width along y] before `yaw`.
    #[serde(default)]
    pub size: Option<Point>,
    #[serde(default)]
    pub yaw: f64,
    /// Cylinder radius.
    #[serde(default)]
    pub radius: Option<f64>,
    pub height: f64,
    pub color: Rgb,
}

#[derive(Deserialize, Debug, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum MarkingKind {
    RestrictedZone,
    Hazard,
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct MarkingSpec {
    #[serde(default)]
    pub name: Option<String>,
    pub kind: MarkingKind,
    pub polygon: Vec<Point>,
    pub color: Rgb,
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct CableSpec {
    #[serde(default)]
    pub name: Option<String>,
    pub path: Vec<Point>,
    #[serde(default = "default_cable_width")]
    pub width: f64,
    #[serde(default)]
    pub color: Option<Rgb>,
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct PedestrianSpec {
    #[serde(default)]
    pub name: Option<String>,
    #[serde(default)]
    pub identity: Option<String>,
    pub waypoints: Vec<Point>,
    /// Walking speed, m/s.
    pub speed: f64,
    /// Walk the waypoints as a loop (true) or back and forth (false).
    #[serde(default = "default_true", rename = "loop")]
    pub looped: bool,
    #[serde(default = "default_person_radius")]
    pub radius: f64,
    #[serde(default = "default_person_height")]
    pub height: f64,
    #[serde(default)]
    pub color: Option<Rgb>,
}

fn default_wall_thickness() -> f64 {
    0.15
}
fn default_wall_height() -> f64 {
    2.5
}
fn default_cable_width() -> f64 {
    0.03
}
fn default_true() -> bool {
    true
}
fn default_person_radius() -> f64 {
    0.25
}
fn default_person_height() -> f64 {
    1.75
}

const WALL_COLOR: Rgb = [190, 186, 176];
const OBSTACLE_COLOR: Rgb = [120, 110, 100];
const CABLE_COLOR: Rgb = [25, 25, 25];
const PERSON_COLOR: Rgb = [60, 80, 150];
const FLOOR_COLOR: Rgb = [150, 150, 146];

/// Parses and validates a scenario.
pub fn parse(text: &str) -> Result<World, ScenarioError> {
    let file: ScenarioFile = toml::from_str(text).map_err(|e| ScenarioError::Syntax(e.to_string()))?;
    validate(&file)
}

fn check_finite(field: &str, v: f64) -> Result<(), ScenarioError> {
    if v.is_finite() { Ok(()) } else { Err(ScenarioError::invalid(field, format!("{v} is not a finite number"))) }
}

fn check_positive(field: &str, v: f64, max: f64) -> Result<(), ScenarioError> {
    check_finite(field, v)?;
    if v <= 0.0 || v > max {
        return Err(ScenarioError::invalid(field, format!("{v} must be > 0 and ≤ {max}")));
    }
    Ok(())
}

fn points(field: &str, pts: &[Point]) -> Result<Vec<Vec2>, ScenarioError> {
    pts.iter()
        .enumerate()
        .map(|(i, p)| {
            check_finite(&format!("{field}[{i}]"), p[0])?;
            check_finite(&format!("{field}[{i}]"), p[1])?;
            Ok(Vec2::new(p[0], p[1]))
        })
        .collect()
}

fn polygon(field: &str, pts: &[Point]) -> Result<Vec<Vec2>, ScenarioError> {
    if pts.len() < 3 {
        return Err(ScenarioError::invalid(field, format!("a polygon needs at least 3 vertices, got {}", pts.len())));
    }
    let mut v = points(field, pts)?;
    let area2 = signed_area2(&v);
    if let Some((i, j)) = self_intersection(&v)
        && (area2.abs() >= 1e-6 || !v.windows(2).any(|w| w[0] == w[1]))
    {
        return Err(ScenarioError::invalid(
            field,
            format!("polygon is not simple: edge {i} crosses edge {j} (list vertices in order around the outline)"),
        ));
    }
    if area2.abs() < 1e-6 {
        return Err(ScenarioError::invalid(field, "polygon has zero area (collinear or repeated vertices)"));
    }
    if area2 < 0.0 {
        v.reverse();
    }
    Ok(v)
}

fn class_name(field: &str, class_id: i32) -> Result<&'static str, ScenarioError> {
    vlnav_proto::coco::name(class_id).ok_or_else(|| {
        ScenarioError::invalid(field, format!("{class_id} is not a COCO-80 class id (0 person … 79 toothbrush)"))
    })
}

fn check_identity(field: &str, identity: &Option<String>) -> Result<String, ScenarioError> {
    match identity {
        None => Ok(String::new()),
        Some(s) if s.trim().is_empty() => {
            Err(ScenarioError::invalid(field, "identity must not be empty (omit it instead)"))
        }
        Some(s) => Ok(s.trim().to_lowercase()),
    }
}

/// Validates a parsed scenario file into a world.
pub fn validate(f: &ScenarioFile) -> Result<World, ScenarioError> {
    if f.name.trim().is_empty() {
        return Err(ScenarioError::invalid("name", "must not be empty"));
    }
    let mut entities: Vec<Entity> = vec![Entity {
        instance_id: 1,
        name: "floor".into(),
        class_id: -1,
        identity: String::new(),
        semantic: Semantic::Floor,
    }];
    let mut solids = Vec::new();
    let mut markings = Vec::new();
    let mut pedestrians = Vec::new();
    let mut next_entity =
        |name: String, class_id: i32, identity: String, semantic: Semantic| -> Result<u16, ScenarioError> {
            let id = entities.len() + 1;
            let id = u16::try_from(id).map_err(|_| ScenarioError::invalid("objects", "more than 65534 entities"))?;
            entities.push(Entity { instance_id: id, name, class_id, identity, semantic });
            Ok(id)
        };

    for (i, w) in f.walls.iter().enumerate() {
        let field = format!("walls[{i}]");
        if w.path.len() < 2 {
            return Err(ScenarioError::invalid(format!("{field}.path"), "a wall path needs at least 2 points"));
        }
        let pts = points(&format!("{field}.path"), &w.path)?;
        check_positive(&format!("{field}.thickness"), w.thickness, 5.0)?;
        check_positive(&format!("{field}.height"), w.height, 50.0)?;
        let id = next_entity(w.name.clone().unwrap_or_else(|| format!("wall {i}")), -1, String::new(), Semantic::Wall)?;
        let n = pts.len();
        let segments = if w.closed { n } else { n - 1 };
        for s in 0..segments {
            let (a, b) = (pts[s], pts[(s + 1) % n]);
            let len = (b - a).norm();
            if len < 1e-6 {
                return Err(ScenarioError::invalid(
                    format!("{field}.path[{}]", (s + 1) % n),
                    "repeats the previous point",
                ));
            }
            // Extend each segment by half the thickness so corners close.
            let d = (b - a).scale(w.thickness / 2.0 / len);
            solids.push(Solid {
                entity: id,
                shape: Shape::Polygon(segment_quad(a - d, b + d, w.thickness)),
                height: w.height,
                color: w.color.unwrap_or(WALL_COLOR),
            });
        }
    }
    for (i, o) in f.obstacles.iter().enumerate() {
        let field = format!("obstacles[{i}]");
        let poly = polygon(&format!("{field}.polygon"), &o.polygon)?;
        check_positive(&format!("{field}.height"), o.height, 50.0)?;
        let id = next_entity(
            o.name.clone().unwrap_or_else(|| format!("obstacle {i}")),
            -1,
            String::new(),
            Semantic::Obstacle,
        )?;
        solids.push(Solid {
            entity: id,
            shape: Shape::Polygon(poly),
            height: o.height,
            color: o.color.unwrap_or(OBSTACLE_COLOR),
        });
    }
    for (i, o) in f.objects.iter().enumerate() {
        let field = format!("objects[{i}]");
        let cls = class_name(&format!("{field}.class_id"), o.class_id)?;
        let identity = check_identity(&format!("{field}.identity"), &o.identity)?;
        if !identity.is_empty() && o.class_id != 0 {
            return Err(ScenarioError::invalid(
                format!("{field}.identity"),
                format!("only persons (class_id 0) carry an identity, this object is class {} ({cls})", o.class_id),
            ));
        }
        let centre = points(&format!("{field}.position"), &[o.position])?[0];
        check_positive(&format!("{field}.height"), o.height, 50.0)?;
        check_finite(&format!("{field}.yaw"), o.yaw)?;
        let shape = match o.shape {
            ShapeKind::Box => {
                let size = o.size.ok_or_else(|| {
                    ScenarioError::invalid(format!("{field}.size"), "a box needs size = [length, width]")
                })?;
                check_positive(&format!("{field}.size[0]"), size[0], 100.0)?;
                check_positive(&format!("{field}.size[1]"), size[1], 100.0)?;
                if o.radius.is_some() {
                    return Err(ScenarioError::invalid(format!("{field}.radius"), "a box has no radius (use size)"));
                }
                Shape::Polygon(box_polygon(centre, size, o.yaw))
            }
            ShapeKind::Cylinder => {
                let r = o
                    .radius
                    .ok_or_else(|| ScenarioError::invalid(format!("{field}.radius"), "a cylinder needs a radius"))?;
                check_positive(&format!("{field}.radius"), r, 50.0)?;
                if o.size.is_some() {
                    return Err(ScenarioError::invalid(format!("{field}.size"), "a cylinder has no size (use radius)"));
                }
                Shape::Circle { centre, radius: r }
            }
        };
        let id =
            next_entity(o.name.clone().unwrap_or_else(|| cls.to_string()), o.class_id, identity, Semantic::Object)?;
        solids.push(Solid { entity: id, shape, height: o.height, color: o.color });
    }
    for (i, m) in f.markings.iter().enumerate() {
        let field = format!("markings[{i}]");
        let poly = polygon(&format!("{field}.polygon"), &m.polygon)?;
        let semantic = match m.kind {
            MarkingKind::RestrictedZone => Semantic::RestrictedZone,
            MarkingKind::Hazard => Semantic::Hazard,
        };
        let id = next_entity(m.name.clone().unwrap_or_else(|| format!("marking {i}")), -1, String::new(), semantic)?;
        markings.push(Marking { entity: id, shapes: vec![Shape::Polygon(poly)], color: m.color });
    }
    for (i, c) in f.cables.iter().enumerate() {
        let field = format!("cables[{i}]");
        if c.path.len() < 2 {
            return Err(ScenarioError::invalid(format!("{field}.path"), "a cable path needs at least 2 points"));
        }
        let pts = points(&format!("{field}.path"), &c.path)?;
        check_positive(&format!("{field}.width"), c.width, 0.5)?;
        let mut shapes = Vec::new();
        for s in 0..pts.len() - 1 {
            if (pts[s + 1] - pts[s]).norm() < 1e-6 {
                return Err(ScenarioError::invalid(format!("{field}.path[{}]", s + 1), "repeats the previous point"));
            }
            shapes.push(Shape::Polygon(segment_quad(pts[s], pts[s + 1], c.width)));
        }
        let id =
            next_entity(c.name.clone().unwrap_or_else(|| format!("cable {i}")), -1, String::new(), Semantic::Cable)?;
        markings.push(Marking { entity: id, shapes, color: c.color.unwrap_or(CABLE_COLOR) });
    }
    for (i, p) in f.pedestrians.iter().enumerate() {
        let field = format!("pedestrians[{i}]");
        if p.waypoints.len() < 2 {
            return Err(ScenarioError::invalid(
                format!("{field}.waypoints"),
                "a pedestrian needs at least 2 waypoints",
            ));
        }
        let wps = points(&format!("{field}.waypoints"), &p.waypoints)?;
        for k in 1..wps.len() {
            if (wps[k] - wps[k - 1]).norm() < 1e-6 {
                return Err(ScenarioError::invalid(format!("{field}.waypoints[{k}]"), "repeats the previous waypoint"));
            }
        }
        check_positive(&format!("{field}.speed"), p.speed, 3.0)?;
        check_positive(&format!("{field}.radius"), p.radius, 2.0)?;
        check_positive(&format!("{field}.height"), p.height, 3.0)?;
        let identity = check_identity(&format!("{field}.identity"), &p.identity)?;
        let name = p
            .name
            .clone()
            .unwrap_or_else(|| if identity.is_empty() { format!("pedestrian {i}") } else { identity.clone() });
        let id = next_entity(name, 0, identity, Semantic::Object)?;
        pedestrians.push(Pedestrian::new(
            id,
            wps,
            p.speed,
            p.looped,
            p.radius,
            p.height,
            p.color.unwrap_or(PERSON_COLOR),
        ));
    }

    let camera = camera_config(&f.camera)?;
    for (i, v) in f.robot.start.iter().enumerate() {
        check_finite(&format!("robot.start[{i}]"), *v)?;
    }
    let start = Pose2::new(f.robot.start[0], f.robot.start[1], f.robot.start[2]);
    let husky = HuskyParams::default();
    let slip = f.robot.slip.clone().unwrap_or_default();
    slip.validate().map_err(|(k, m)| ScenarioError::invalid(format!("robot.slip.{k}"), m))?;
    let footprint = OrientedRect::new(start, husky.length, husky.width);
    for s in &solids {
        if footprint.overlaps(&s.shape) {
            let e = &entities[s.entity as usize - 1];
            return Err(ScenarioError::invalid(
                "robot.start",
                format!(
                    "the robot's footprint at ({}, {}) overlaps {} `{}`",
                    start.x,
                    start.y,
                    e.semantic.as_str(),
                    e.name
                ),
            ));
        }
    }
    for p in &pedestrians {
        if footprint.overlaps(&p.shape_at(0.0)) {
            return Err(ScenarioError::invalid(
                "robot.start",
                "the robot's footprint overlaps a pedestrian's starting point",
            ));
        }
    }
    Ok(World {
        name: f.name.clone(),
        description: f.description.clone(),
        start,
        camera,
        slip,
        floor_color: f.floor_color.unwrap_or(FLOOR_COLOR),
        entities,
        solids,
        markings,
        pedestrians,
    })
}

fn camera_config(c: &CameraSpec) -> Result<CameraConfig, ScenarioError> {
    let mut cam = CameraConfig::default();
    if c.width.is_some() || c.height.is_some() {
        let w = c.width.unwrap_or(cam.width);
        let h = c.height.unwrap_or(cam.height);
        cam = cam.with_resolution(w, h).map_err(|m| ScenarioError::invalid("camera.width", m))?;
    }
    for (k, v, slot) in
        [("fx", c.fx, &mut cam.fx), ("fy", c.fy, &mut cam.fy), ("cx", c.cx, &mut cam.cx), ("cy", c.cy, &mut cam.cy)]
    {
        if let Some(v) = v {
            check_finite(&format!("camera.{k}"), v)?;
            *slot = v;
        }
    }
    if let Some(m) = c.mount {
        for (i, v) in m.iter().enumerate() {
            check_finite(&format!("camera.mount[{i}]"), *v)?;
        }
        cam.mount = m;
    }
    if let Some(y) = c.mount_yaw {
        check_finite("camera.mount_yaw", y)?;
        cam.mount_yaw = y;
    }
    if let Some(v) = c.depth_min_m {
        cam.depth_min_m = v;
    }
    if let Some(v) = c.depth_max_m {
        cam.depth_max_m = v;
    }
    if let Some(v) = c.depth_noise_k {
        cam.depth_noise_k = v;
    }
    if let Some(v) = c.depth_reliable_max_m {
        cam.depth_reliable_max_m = v;
    }
    if let Some(v) = c.stereo_baseline_m {
        cam.stereo_baseline_m = v;
    }
    cam.validate().map_err(|(k, m)| ScenarioError::invalid(format!("camera.{k}"), m))?;
    Ok(cam)
}

#[cfg(test)]
mod tests {
    use super::*;

    const BASE: &str = r#"
name = "t"
[robot]
start = [0.0, 0.0, 0.0]
[[walls]]
path = [[-2, -3], [8, -3], [8, 3], [-2, 3]]
closed = true
[[objects]]
name = "chair"
class_id = 56
position = [4.0, 1.0]
shape = "box"
size = [0.5, 0.5]
height = 0.9
color = [90, 60, 30]
"#;

    fn err_field(text: &str) -> String {
        let e = parse(text).unwrap_err();
        e.field().unwrap_or_else(|| panic!("expected a field error, got {e}")).to_string()
    }

    #[test]
    fn a_valid_scenario_builds_its_entities() {
        let w = parse(BASE).unwrap();
        assert_eq!(w.entities.len(), 3);
        assert_eq!(w.entities[2].class_id, 56);
        assert_eq!(w.solids.len(), 5); // four wall segments and the chair
    }

    #[test]
    fn an_unknown_class_is_rejected_naming_the_field() {
        let e = parse(&BASE.replace("class_id = 56", "class_id = 95")).unwrap_err();
        assert_eq!(e.field(), Some("objects[0].class_id"));
        assert!(e.to_string().contains("95 is not a COCO-80 class id"), "{e}");
    }

    #[test]
    fn a_malformed_polygon_is_rejected_naming_the_field() {
        let bowtie = format!("{BASE}\n[[obstacles]]\npolygon = [[1, 1], [2, 2], [2, 1], [1, 2]]\nheight = 1.0\n");
        let e = parse(&bowtie).unwrap_err();
        assert_eq!(e.field(), Some("obstacles[0].polygon"));
        assert!(e.to_string().contains("not simple"), "{e}");
        let two = format!(
            "{BASE}\n[[markings]]\nkind = \"restricted_zone\"\npolygon = [[1, 1], [2, 2]]\ncolor = [200, 0, 0]\n"
        );
        assert_eq!(err_field(&two), "markings[0].polygon");
        let flat = format!("{BASE}\n[[obstacles]]\npolygon = [[1, 1], [2, 2], [3, 3]]\nheight = 1.0\n");
        assert!(parse(&flat).unwrap_err().to_string().contains("zero area"));
    }

    #[test]
    fn a_start_inside_an_obstacle_is_rejected_naming_the_field() {
        let e = parse(&BASE.replace("position = [4.0, 1.0]", "position = [0.3, 0.2]")).unwrap_err();
        assert_eq!(e.field(), Some("robot.start"));
        assert!(e.to_string().contains("chair"), "{e}");
        // Touching a wall counts too.
        assert_eq!(err_field(&BASE.replace("start = [0.0, 0.0, 0.0]", "start = [0.0, 2.7, 0.0]")), "robot.start");
    }

    #[test]
    fn other_field_errors_are_named() {
        assert_eq!(err_field(&BASE.replace("height = 0.9", "height = -1.0")), "objects[0].height");
        assert_eq!(err_field(&BASE.replace("shape = \"box\"", "shape = \"cylinder\"")), "objects[0].radius");
        assert_eq!(
            err_field(&BASE.replace("name = \"chair\"", "name = \"chair\"\nidentity = \"david\"")),
            "objects[0].identity"
        );
        let ped = format!("{BASE}\n[[pedestrians]]\nwaypoints = [[5, -2]]\nspeed = 0.5\n");
        assert_eq!(err_field(&ped), "pedestrians[0].waypoints");
        let fast = format!("{BASE}\n[[pedestrians]]\nwaypoints = [[5, -2], [5, 2]]\nspeed = 9.0\n");
        assert_eq!(err_field(&fast), "pedestrians[0].speed");
        let cam = format!("{BASE}\n[camera]\ndepth_min_m = 12.0\n");
        assert_eq!(err_field(&cam), "camera.depth_min_m");
        let cable = format!("{BASE}\n[[cables]]\npath = [[1, 1], [1, 1]]\n");
        assert_eq!(err_field(&cable), "cables[0].path[1]");
    }

    #[test]
    fn unknown_keys_and_kinds_are_syntax_errors_that_say_where() {
        let e = parse(&BASE.replace("shape = \"box\"", "shape = \"sphere\"")).unwrap_err();
        assert!(matches!(e, ScenarioError::Syntax(_)));
        assert!(e.to_string().contains("sphere"), "{e}");
        let e = parse(&BASE.replace("height = 0.9", "height = 0.9\ncolour = [1, 2, 3]")).unwrap_err();
        assert!(e.to_string().contains("colour"), "{e}");
    }
}
