//! The simulation loop: a world, a Husky in it, its camera, and the ground
//! truth the metrics read (pose, path length, collision events).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::camera::{CameraConfig, Frame, Renderer};
use crate::crowd::Crowd;
use crate::geometry::{OrientedRect, Pose2, Vec2};
use crate::robot::{HuskyParams, RobotState, Twist, integrate};
use crate::world::World;

/// Physics substep, seconds (commands are applied for whole steps made of these).
pub const SUBSTEP_S: f64 = 0.01;
/// A footprint this close to a solid still counts as touching it, so a robot
/// pressed against a wall is one contact, not one per substep.
const CONTACT_MARGIN_M: f64 = 0.02;

/// Ground truth at the current simulation time.
#[derive(Clone, Debug, PartialEq)]
pub struct Truth {
    pub stamp: f64,
    pub pose: Pose2,
    pub twist: Twist,
    pub path_length_m: f64,
    /// Contact events with walls, obstacles, objects or pedestrians.
    pub hard_collisions: u32,
    /// Those of them the robot's own motion made (the rest: a person
    /// walked into it). See `docs/simulation.md`, "Contact and its cause".
    pub hard_collisions_by_robot: u32,
    /// Contact events with pedestrians (included in `hard_collisions`).
    pub pedestrian_contacts: u32,
    pub pedestrian_contacts_by_robot: u32,
    /// Entries into restricted zones, hazards or onto cables.
    pub soft_collisions: u32,
    /// The footprint touches something now.
    pub in_hard_contact: bool,
    /// The footprint lies in a no-go marking now.
    pub in_no_go: bool,
    /// Where each pedestrian is now, in the world's order.
    pub pedestrians: Vec<Vec2>,
    /// World pose of the odometry frame's origin.
    pub odom_origin: Pose2,
}

/// What the robot believes: the integrated wheel odometry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Odometry {
    pub stamp: f64,
    pub pose: Pose2,
    pub twist: Twist,
}

/// A simulated Husky in a world. Deterministic: the same world, seed and
/// command sequence give the same run, bit for bit. The physics and the
/// camera noise draw from separate streams, so rendering (or its resolution)
/// never changes the trajectory.
pub struct Simulator {
    world: World,
    camera: CameraConfig,
    params: HuskyParams,
    state: RobotState,
    time: f64,
    steps: u64,
    path_length: f64,
    hard: u32,
    hard_by_robot: u32,
    pedestrian_contacts: u32,
    pedestrian_contacts_by_robot: u32,
    soft: u32,
    touching: Vec<u16>,
    crowd: Crowd,
    inside: Vec<u16>,
    physics_rng: ChaCha8Rng,
    camera_rng: ChaCha8Rng,
    renderer: Renderer,
}

impl Simulator {
    pub fn new(world: World, seed: u64) -> Self {
        let camera = world.camera.clone();
        let state = RobotState::at(world.start);
        let mut physics_rng = ChaCha8Rng::seed_from_u64(seed);
        physics_rng.set_stream(1);
        let mut camera_rng = ChaCha8Rng::seed_from_u64(seed);
        camera_rng.set_stream(2);
        let mut sim = Self {
            world,
            camera,
            params: HuskyParams::default(),
            state,
            time: 0.0,
            steps: 0,
            path_length: 0.0,
            hard: 0,
            hard_by_robot: 0,
            pedestrian_contacts: 0,
            pedestrian_contacts_by_robot: 0,
            soft: 0,
            touching: Vec::new(),
            crowd: Crowd::default(),
            inside: Vec::new(),
            physics_rng,
            camera_rng,
            renderer: Renderer::new(),
        };
        sim.crowd = Crowd::new(&sim.world);
        sim.inside = sim.markings_under(&sim.state.truth);
        sim
    }

    /// Replaces the camera (resolution, mount…); the world's camera is the default.
    pub fn set_camera(&mut self, camera: CameraConfig) {
        self.camera = camera;
    }

    pub fn camera(&self) -> &CameraConfig {
        &self.camera
    }

    pub fn world(&self) -> &World {
        &self.world
    }

    pub fn params(&self) -> &HuskyParams {
        &self.params
    }

    /// Simulation time, seconds since the episode began.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Applies `cmd` (the platform controller's input) for `dt` seconds.
    pub fn step(&mut self, cmd: Twist, dt: f64) {
        if !(dt.is_finite() && dt > 0.0) {
            return;
        }
        let n = (dt / SUBSTEP_S).ceil().max(1.0) as usize;
        let h = dt / n as f64;
        for _ in 0..n {
            self.substep(cmd, h);
        }
        self.steps += 1;
    }

    fn substep(&mut self, cmd: Twist, h: f64) {
        let m = integrate(&self.state, cmd, &self.params, &self.world.slip, h, &mut self.physics_rng);
        self.time += h;
        self.state.wheel_twist = m.wheel_twist;
        self.state.odom = m.odom;
        let candidate = OrientedRect::new(m.truth, self.params.length, self.params.width);
        // What the robot's own motion reaches (within the contact margin),
        // with everything else where it was; of that, what the body itself
        // would overlap stops it.
        let robot_made = self.solids_overlapping(&candidate.inflate(CONTACT_MARGIN_M));
        let blocked = self.solids_overlapping_among(&candidate, &robot_made);
        let moved = blocked.is_empty();
        let previous = self.state.truth;
        let mut touching = if moved {
            self.path_length += m.truth.distance(&self.state.truth);
            self.state.truth = m.truth;
            self.state.truth_twist = m.truth_twist;
            Vec::new()
        } else {
            // The body stops against what it hit; the wheels keep turning
            // (odometry keeps counting) as a real skid-steer's would.
            self.state.truth_twist = Twist::ZERO;
            blocked
        };
        let people = !self.world.pedestrians.is_empty();
        if people {
            let body = OrientedRect::new(self.state.truth, self.params.length, self.params.width);
            let velocity = Vec2::new(self.state.truth.x - previous.x, self.state.truth.y - previous.y).scale(1.0 / h);
            self.crowd.step(&self.world, &body, velocity, h);
        }
        let here = if moved && !people {
            // Nothing else moved: the robot now touches what its move reached.
            robot_made.clone()
        } else {
            let rect = OrientedRect::new(self.state.truth, self.params.length, self.params.width);
            self.solids_overlapping(&rect.inflate(CONTACT_MARGIN_M))
        };
        for id in here {
            if !touching.contains(&id) {
                touching.push(id);
            }
        }
        touching.sort_unstable();
        for &id in touching.iter().filter(|id| !self.touching.contains(id)) {
            let by_robot = robot_made.contains(&id);
            let person = self.world.pedestrians.iter().any(|p| p.entity == id);
            self.hard += 1;
            self.hard_by_robot += by_robot as u32;
            self.pedestrian_contacts += person as u32;
            self.pedestrian_contacts_by_robot += (person && by_robot) as u32;
        }
        self.touching = touching;

        let inside = self.markings_under(&self.state.truth);
        self.soft += inside.iter().filter(|id| !self.inside.contains(id)).count() as u32;
        self.inside = inside;
    }

    /// Entities (solids and people) whose outline `rect` overlaps.
    fn solids_overlapping(&self, rect: &OrientedRect) -> Vec<u16> {
        self.overlapping(rect, |_| true)
    }

    /// Those of `ids` whose outline `rect` overlaps.
    fn solids_overlapping_among(&self, rect: &OrientedRect, ids: &[u16]) -> Vec<u16> {
        if ids.is_empty() {
            return Vec::new();
        }
        self.overlapping(rect, |id| ids.contains(&id))
    }

    fn overlapping(&self, rect: &OrientedRect, consider: impl Fn(u16) -> bool) -> Vec<u16> {
        let mut ids: Vec<u16> = self
            .world
            .solids
            .iter()
            .filter(|s| consider(s.entity) && rect.overlaps(&s.shape))
            .map(|s| s.entity)
            .collect();
        ids.extend(
            self.world
                .pedestrians
                .iter()
                .zip(self.crowd.shapes(&self.world))
                .filter(|(p, shape)| consider(p.entity) && rect.overlaps(shape))
                .map(|(p, _)| p.entity),
        );
        ids.sort_unstable();
        ids.dedup();
        ids
    }

    fn markings_under(&self, pose: &Pose2) -> Vec<u16> {
        let rect = OrientedRect::new(*pose, self.params.length, self.params.width);
        let mut ids: Vec<u16> = self
            .world
            .markings
            .iter()
            .filter(|m| self.world.entity(m.entity).is_some_and(|e| e.semantic.is_no_go()))
            .filter(|m| m.shapes.iter().any(|s| rect.overlaps(s)))
            .map(|m| m.entity)
            .collect();
        ids.sort_unstable();
        ids.dedup();
        ids
    }

    /// Renders the camera's view now into `frame` (reusing its buffers).
    pub fn render_into(&mut self, frame: &mut Frame) {
        let people: Vec<Vec2> = self.crowd.positions().collect();
        self.renderer.render(&self.world, &self.camera, &self.state.truth, &people, &mut self.camera_rng, frame);
    }

    pub fn render(&mut self) -> Frame {
        let mut f = Frame::default();
        self.render_into(&mut f);
        f
    }

    pub fn truth(&self) -> Truth {
        Truth {
            stamp: self.time,
            pose: self.state.truth,
            twist: self.state.truth_twist,
            path_length_m: self.path_length,
            hard_collisions: self.hard,
            hard_collisions_by_robot: self.hard_by_robot,
            pedestrian_contacts: self.pedestrian_contacts,
            pedestrian_contacts_by_robot: self.pedestrian_contacts_by_robot,
            soft_collisions: self.soft,
            in_hard_contact: !self.touching.is_empty(),
            in_no_go: !self.inside.is_empty(),
            pedestrians: self.crowd.positions().collect(),
            odom_origin: self.state.odom_origin,
        }
    }

    pub fn odometry(&self) -> Odometry {
        Odometry { stamp: self.time, pose: self.state.odom, twist: self.state.wheel_twist }
    }

    /// Re-anchors odometry at the robot's current pose.
    pub fn reset_odometry(&mut self) {
        self.state.reset_odometry();
    }

    /// Distance from the true position to a world point (final pose error).
    pub fn position_error(&self, x: f64, y: f64) -> f64 {
        (self.state.truth.x - x).hypot(self.state.truth.y - y)
    }

    /// The world point an odometry-frame pose corresponds to, given the
    /// current odometry anchor (exact when odometry does not drift).
    pub fn odom_to_world(&self, p: &Pose2) -> Pose2 {
        self.state.odom_origin.compose(p)
    }
}
